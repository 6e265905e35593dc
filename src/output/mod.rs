//! Outputs: the fused pose to the machines and people that use it.
//!
//! - [`vpe`]: pure conversion of the fused pose to MAVLink messages (NED/FRD).
//! - [`mavlink_out`]: the MAVLink endpoints (UDP, TCP, serial, mavlink-server on Zenoh).
//! - [`zenoh_out`]: JSON and ROS 2 CDR on Zenoh.

pub mod mavlink_out;
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

/// What only one kind of output has.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum OutputDetail {
    Mavlink {
        configured_rate_hz: f64,
        heartbeats: u64,
        origin_sent: u64,
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
    },
}
