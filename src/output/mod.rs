//! Outputs: the fused pose to the machines and people that use it.
//!
//! - [`vpe`]: pure conversion of the fused pose to MAVLink messages (NED/FRD).
//! - [`mavlink_out`]: the MAVLink endpoints (UDP, TCP, serial, mavlink-server on Zenoh).
//! - [`zenoh_out`]: JSON and ROS 2 CDR on Zenoh.

pub mod mavlink_out;
pub mod precision;
pub mod summary;
pub mod timesync;
pub mod vpe;
pub mod zenoh_out;

/// One output as `/api/v1/status` shows it (`outputs[]`, web/PROTOCOL.md).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct OutputStatus {
    pub name: &'static str,
    pub kind: &'static str,
    pub endpoint: String,
    /// MAVLink: VISION_POSITION_ESTIMATE sent; Zenoh: poses published.
    pub sent: u64,
    pub dropped: u64,
    pub errors: u64,
    pub last_error: Option<String>,
    pub sending: bool,
    pub not_sending_reason: Option<String>,
    /// Poses sent per second over the last second; 0 once sending stopped.
    pub rate_hz: f64,
    /// Time since the last pose sent, ms; `None`: never.
    pub last_sent_age_ms: Option<f64>,
    #[serde(flatten)]
    pub detail: OutputDetail,
}

/// An output that sent nothing for this long is not sending, µs.
pub const SENDING_WITHIN_US: i64 = 2_000_000;

/// When an output last sent a pose and how fast it sends: what its status derives
/// "sending", `rate_hz` and `last_sent_age_ms` from.
#[derive(Debug, Default)]
pub struct SendClock {
    /// Host time of the last send, µs (0: never).
    last_us: std::sync::atomic::AtomicU64,
    rate: std::sync::Mutex<crate::clock::RateMeter>,
}

impl SendClock {
    /// A pose was sent at `now`.
    pub fn sent(&self, now: i64) {
        self.last_us
            .store(now.max(0) as u64, std::sync::atomic::Ordering::Relaxed);
        crate::sync::lock(&self.rate).tick(now);
    }

    /// Time since the last send at `now`, µs; `None`: never sent.
    pub fn age_us(&self, now: i64) -> Option<i64> {
        let last = self.last_us.load(std::sync::atomic::Ordering::Relaxed) as i64;
        (last > 0).then_some(now - last)
    }

    /// A pose went out within [`SENDING_WITHIN_US`] of `now`.
    pub fn recent(&self, now: i64) -> bool {
        self.age_us(now).is_some_and(|a| a < SENDING_WITHIN_US)
    }

    /// Sends per second over the last second; 0 once sending stopped.
    pub fn rate_hz(&self, now: i64) -> f64 {
        crate::sync::lock(&self.rate).rate_hz_at(now)
    }

    pub fn age_ms(&self, now: i64) -> Option<f64> {
        self.age_us(now).map(|a| a as f64 / 1e3)
    }
}

/// What only one kind of output has.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum OutputDetail {
    Mavlink {
        configured_rate_hz: f64,
        heartbeats: u64,
        origin_sent: u64,
        /// SETUP_SIGNING sent on request (`POST /api/v1/control/setup-signing`).
        setup_signing_sent: u64,
        /// Ticks with nothing sent because the estimate was invalid, stale or non-finite.
        withheld: u64,
        reset_counter: u64,
        links: Vec<mavlink_out::LinkStatus>,
        /// The autopilot's clock as TIMESYNC tells it.
        timesync: timesync::TimeSyncStatus,
    },
    Zenoh {
        debug_points: u64,
        events: u64,
        health: u64,
        /// px4_msgs/VehicleOdometry sent (`[output] px4_odometry`), poses not sent as
        /// one, and why the last was not.
        px4_odometry_sent: u64,
        px4_odometry_withheld: u64,
        px4_odometry_not_sending: Option<String>,
    },
}
