//! MAVLink TIMESYNC both ways, as PX4 (`mavlink_timesync`) and MAVROS do it: answer the
//! autopilot's requests with our clock, send our own and estimate the autopilot's clock
//! from its answers, so the poses sent carry its time. PX4 ignores a VPE's `usec` (and
//! stamps it at arrival, losing its age) until its own estimate has converged; ArduPilot
//! corrects `usec` for jitter against its clock.
//!
//! Pure: times are passed in (local: the host clock, ns). The model is
//! `remote = a + rate · (local − t0)`, fitted by least squares over the last
//! [`WINDOW`] samples whose round trip is near the smallest seen (a late answer says
//! little about when the autopilot read its clock). `rate` is 1 unless the samples say
//! the autopilot's clock runs faster or slower by more than [`RATE_TOLERANCE`] (SITL at
//! `--speedup N`): then it is reported and used. An answer far off the model three
//! times running is an autopilot that restarted: the model starts again.

use serde::Serialize;
use std::collections::VecDeque;

/// Samples the model is fitted over (at 2 Hz: the last 10 s).
pub const WINDOW: usize = 20;
/// Good samples before the estimate is used.
pub const CONVERGE_SAMPLES: usize = 5;
/// A round trip longer than this is no sample, ns.
pub const MAX_RTT_NS: i64 = 500_000_000;
/// A sample's round trip may exceed the smallest of the window by this factor plus
/// [`RTT_SLACK_NS`].
const RTT_FACTOR: f64 = 3.0;
const RTT_SLACK_NS: f64 = 2e6;
/// A clock whose rate differs from ours by less than this runs at ours.
pub const RATE_TOLERANCE: f64 = 0.01;
/// An answer this far off the model (or 20 round trips), ns, is off.
const JUMP_NS: f64 = 100e6;
/// Off answers in a row that restart the model.
const JUMPS_TO_RESET: u32 = 3;

/// What came of a TIMESYNC message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handled {
    /// The autopilot's request: send TIMESYNC { tc1, ts1 } back.
    Answer { tc1: i64, ts1: i64 },
    /// An answer to ours, used.
    Used,
    /// An answer to ours, not used (round trip too long, off the model).
    Rejected,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    /// Local time halfway through the round trip, ns.
    local_ns: f64,
    remote_ns: f64,
    rtt_ns: f64,
}

/// The autopilot's clock as far as its TIMESYNC answers tell.
#[derive(Debug, Clone, Default)]
pub struct TimeSync {
    window: VecDeque<Sample>,
    /// (t0 local, a remote at t0, rate), once converged.
    model: Option<(f64, f64, f64)>,
    jumps: u32,
    answered: u64,
    used: u64,
    rejected: u64,
    resets: u32,
    last_rtt_ns: Option<f64>,
}

/// The part of the MAVLink output's status about time (`timesync` in `/api/v1/status`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimeSyncStatus {
    /// The autopilot's clock is known: poses carry its time.
    pub converged: bool,
    /// Autopilot clock minus ours at the newest sample, ms.
    pub offset_ms: Option<f64>,
    /// The newest used sample's round trip, ms.
    pub rtt_ms: Option<f64>,
    /// The autopilot's clock rate relative to ours (1: the same; SITL --speedup 5: 5).
    pub rate: Option<f64>,
    /// Samples used / rejected; the autopilot's requests answered; model restarts.
    pub used: u64,
    pub rejected: u64,
    pub answered: u64,
    pub resets: u32,
}

impl TimeSync {
    /// A TIMESYNC `(tc1, ts1)` arrived at local time `now_ns`.
    pub fn on_message(&mut self, tc1: i64, ts1: i64, now_ns: i64) -> Handled {
        if tc1 == 0 {
            self.answered += 1;
            return Handled::Answer { tc1: now_ns, ts1 };
        }
        // ts1 comes from the link: an echo of ours, or anything at all.
        let rtt = now_ns.checked_sub(ts1).unwrap_or(i64::MAX);
        if ts1 <= 0 || rtt <= 0 || rtt > MAX_RTT_NS {
            self.rejected += 1;
            return Handled::Rejected;
        }
        let s = Sample {
            local_ns: ts1 as f64 + rtt as f64 / 2.0,
            remote_ns: tc1 as f64,
            rtt_ns: rtt as f64,
        };
        let rtt_min = self
            .window
            .iter()
            .map(|w| w.rtt_ns)
            .fold(s.rtt_ns, f64::min);
        if s.rtt_ns > RTT_FACTOR * rtt_min + RTT_SLACK_NS {
            self.rejected += 1;
            return Handled::Rejected;
        }
        if let Some(pred) = self.predict(s.local_ns) {
            if (s.remote_ns - pred).abs() > JUMP_NS.max(20.0 * rtt_min) {
                self.jumps += 1;
                self.rejected += 1;
                if self.jumps >= JUMPS_TO_RESET {
                    // The autopilot restarted (or its clock was set): start again.
                    self.window.clear();
                    self.model = None;
                    self.jumps = 0;
                    self.resets += 1;
                }
                return Handled::Rejected;
            }
        }
        self.jumps = 0;
        self.window.push_back(s);
        if self.window.len() > WINDOW {
            self.window.pop_front();
        }
        self.last_rtt_ns = Some(s.rtt_ns);
        self.used += 1;
        self.model = (self.window.len() >= CONVERGE_SAMPLES).then(|| fit(&self.window));
        Handled::Used
    }

    /// The autopilot's time at local time `local_ns`, once converged.
    pub fn remote_ns(&self, local_ns: i64) -> Option<i64> {
        self.predict(local_ns as f64).map(|r| r.round() as i64)
    }

    fn predict(&self, local_ns: f64) -> Option<f64> {
        let (t0, a, rate) = self.model?;
        Some(a + rate * (local_ns - t0))
    }

    pub fn status(&self) -> TimeSyncStatus {
        let newest = self.window.back();
        TimeSyncStatus {
            converged: self.model.is_some(),
            offset_ms: newest.map(|s| (s.remote_ns - s.local_ns) / 1e6),
            rtt_ms: self.last_rtt_ns.map(|r| r / 1e6),
            rate: self.model.map(|(_, _, r)| r),
            used: self.used,
            rejected: self.rejected,
            answered: self.answered,
            resets: self.resets,
        }
    }
}

/// `remote = a + rate · (local − t0)` over the window, t0 its newest sample; rate 1
/// unless the fit says otherwise by more than [`RATE_TOLERANCE`].
fn fit(w: &VecDeque<Sample>) -> (f64, f64, f64) {
    let n = w.len() as f64;
    let t0 = w.back().map_or(0.0, |s| s.local_ns);
    let mx = w.iter().map(|s| s.local_ns - t0).sum::<f64>() / n;
    let my = w.iter().map(|s| s.remote_ns).sum::<f64>() / n;
    let sxx: f64 = w.iter().map(|s| (s.local_ns - t0 - mx).powi(2)).sum();
    let sxy: f64 = w
        .iter()
        .map(|s| (s.local_ns - t0 - mx) * (s.remote_ns - my))
        .sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 1.0 };
    let rate = if (slope - 1.0).abs() < RATE_TOLERANCE || !slope.is_finite() || slope <= 0.0 {
        1.0
    } else {
        slope
    };
    (t0, my - rate * mx, rate)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An autopilot whose clock is `offset + rate · local`, answering after `delay`.
    fn exchange(ts: &mut TimeSync, local: i64, offset: i64, rate: f64, rtt: i64) -> Handled {
        let remote_at_mid = offset + (rate * (local + rtt / 2) as f64) as i64;
        ts.on_message(remote_at_mid, local, local + rtt)
    }

    #[test]
    fn answers_requests_with_our_clock() {
        let mut ts = TimeSync::default();
        assert_eq!(
            ts.on_message(0, 777, 5_000),
            Handled::Answer {
                tc1: 5_000,
                ts1: 777
            }
        );
        assert_eq!(ts.status().answered, 1);
        assert!(!ts.status().converged);
    }

    /// Offset known to within the round trip's asymmetry after five samples; a late
    /// answer is not used; the autopilot's time for a pose's stamp is its clock.
    #[test]
    fn converges_and_drops_late_answers() {
        let mut ts = TimeSync::default();
        let offset = -1_700_000_000_000_000_000i64; // remote: time since boot
        let mut t = 1_700_000_000_000_000_000i64 + 123_000_000_000;
        for i in 0..CONVERGE_SAMPLES {
            assert!(!ts.status().converged, "{i}");
            assert_eq!(exchange(&mut ts, t, offset, 1.0, 400_000), Handled::Used);
            t += 500_000_000;
        }
        assert!(ts.status().converged);
        // 80 ms round trip against 0.4 ms ones: not used.
        assert_eq!(
            exchange(&mut ts, t, offset, 1.0, 80_000_000),
            Handled::Rejected
        );
        let remote = ts.remote_ns(t).unwrap();
        assert!(
            (remote - (t + offset)).abs() < 1_000,
            "{}",
            remote - (t + offset)
        );
        let s = ts.status();
        assert_eq!(s.rate, Some(1.0));
        assert!((s.rtt_ms.unwrap() - 0.4).abs() < 1e-9);
        assert!((s.offset_ms.unwrap() - offset as f64 / 1e6).abs() < 1.0);
    }

    /// SITL at --speedup 5: the rate is found and the remote time follows it.
    #[test]
    fn a_clock_at_five_times_ours_is_found() {
        let mut ts = TimeSync::default();
        let mut t = 10_000_000_000i64;
        for _ in 0..10 {
            exchange(&mut ts, t, 0, 5.0, 300_000);
            t += 500_000_000;
        }
        let s = ts.status();
        assert!((s.rate.unwrap() - 5.0).abs() < 1e-3, "{s:?}");
        let later = t + 1_000_000_000;
        let want = 5.0 * later as f64;
        assert!((ts.remote_ns(later).unwrap() as f64 - want).abs() < 1e6);
    }

    /// The autopilot restarts (its clock from 0 again): three answers off the model and
    /// the model starts over, converging on the new clock.
    #[test]
    fn an_autopilot_restart_restarts_the_model() {
        let mut ts = TimeSync::default();
        let mut t = 50_000_000_000i64;
        for _ in 0..8 {
            exchange(&mut ts, t, 1_000_000_000_000, 1.0, 300_000);
            t += 500_000_000;
        }
        let rebooted = -t;
        for _ in 0..JUMPS_TO_RESET {
            assert_eq!(
                exchange(&mut ts, t, rebooted, 1.0, 300_000),
                Handled::Rejected
            );
            t += 500_000_000;
        }
        assert_eq!(ts.status().resets, 1);
        assert!(!ts.status().converged);
        for _ in 0..CONVERGE_SAMPLES {
            assert_eq!(exchange(&mut ts, t, rebooted, 1.0, 300_000), Handled::Used);
            t += 500_000_000;
        }
        assert!((ts.remote_ns(t).unwrap() - (t + rebooted)).abs() < 1_000);
    }

    #[test]
    fn nonsense_answers_are_rejected() {
        let mut ts = TimeSync::default();
        // Extremes that overflow a plain subtraction.
        assert_eq!(ts.on_message(5, 1, i64::MIN), Handled::Rejected);
        assert_eq!(
            ts.on_message(i64::MAX, i64::MAX, i64::MIN),
            Handled::Rejected
        );
        ts = TimeSync::default();
        // An answer to a request we never sent (ts1 in the future), and one a minute late.
        assert_eq!(ts.on_message(5, 2_000, 1_000), Handled::Rejected);
        assert_eq!(ts.on_message(5, 1, 60_000_000_000), Handled::Rejected);
        assert_eq!(ts.on_message(5, -3, 1_000), Handled::Rejected);
        assert_eq!(ts.status().rejected, 3);
    }
}
